"""Odometry tracks against GPS fixes: the position RMSE after one rigid planar alignment.

Odometry starts at its own origin and heading; GPS is in east, north. Every track is compared
at the same fix times (those inside all the tracks' spans; linear interpolation) with the fixes
in a local east-north plane (:func:`fusion.geometry.geodesy.geodetic_to_enu`, origin the first
fix), after the one rotation and translation that fit it best
(:func:`fusion.evaluation.trajectory.se2_alignment`; no scale, so a distance error counts). This
is how issue 11 scored a real outdoor robot's bag. A GPS fix has its own error (metres for a
plain receiver), and the antenna's offset from the base swings with the heading: the RMSE
includes both, so compare tracks with each other rather than with 0.

A fix that jumps away from every track is the receiver's fault (multipath, a jump), not the
tracks'. A track's own error drifts slowly, so each fix's residual (a vector, after the
alignment) is taken against the median residual of the fixes within :data:`OUTLIER_WINDOW`
of it: a fix whose departure from that exceeds :data:`OUTLIER_FACTOR` times the track's
median departure, and :data:`OUTLIER_FLOOR`, for EVERY track compared is left out, each
track aligned again without those fixes, until none is added (at most
:data:`OUTLIER_ROUNDS`). A single-track comparison applies the rule to that track alone.
An independent probe's bag with 20 of its 1976 fixes moved 50 m north had printed 5.24 m
for the fused track, 23.74 m for the bag's odometry (1.55 and 23.21 m with clean fixes):
now all 20 are left out, 1.55 and 23.23 m. Where one track was far worse than the others,
a rule on the residual itself (not its departure) left 2 of the 20 out. The figure with
every fix stays in :attr:`GpsComparison.rmse_all`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from fusion.evaluation.trajectory import se2_alignment
from fusion.geometry.geodesy import geodetic_to_enu

__all__ = ["OUTLIER_FACTOR", "OUTLIER_FLOOR", "OUTLIER_ROUNDS", "OUTLIER_WINDOW",
           "GpsComparison", "compare_with_fixes", "fixes_to_enu"]

#: A fix departing from its neighbours' residual by over this many times the track's median
#: departure is an outlier for it (a Rayleigh-distributed error's median is 1.18 sigma: 5
#: times it is 5.9 sigma).
OUTLIER_FACTOR = 5.0
#: m: and by over this (a good track's median departure can be centimetres).
OUTLIER_FLOOR = 5.0
#: s: the neighbours on either side (a receiver's multipath episode shorter than this stands
#: out; a track's drift does not change much within it).
OUTLIER_WINDOW = 5.0
#: Realignments without the outliers found so far, at most.
OUTLIER_ROUNDS = 5


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
        rmse: per track name, the position RMSE after its own alignment, m, over the fixes
            compared less the outliers (module docstring).
        compared: how many fixes were compared (the same for every track), outliers included.
        outliers: how many of them were left out of ``rmse`` as far from every track.
        rmse_all: per track name, the RMSE over every fix compared (its own alignment).
        span: (first, last) s, the times of the fixes compared.
        gps_in_track_frame: per track name, (K, 2) m, the fixes compared, moved into that
            track's frame by the inverse of its alignment (to draw beside it).
    """

    rmse: dict[str, float] = field(default_factory=dict)
    compared: int = 0
    span: tuple[float, float] = (0.0, 0.0)
    gps_in_track_frame: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    outliers: int = 0
    rmse_all: dict[str, float] = field(default_factory=dict)


def _aligned(name: str, at: NDArray[np.float64], ref: NDArray[np.float64],
             use: NDArray[np.bool_]) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
    """``(theta, shift, residuals (K, 2) m)``: the track ``at`` aligned to ``ref`` over the
    fixes ``use``, and every fix's residual vector from it."""
    try:
        theta, shift, _ = se2_alignment(at[use], ref[use])
    except ValueError as exc:
        raise ValueError(f"{name}: {exc}") from exc
    c, s = np.cos(theta), np.sin(theta)
    return theta, shift, at @ np.array([[c, s], [-s, c]]) + shift - ref


def _departures(t: NDArray[np.float64], residual: NDArray[np.float64],
                use: NDArray[np.bool_]) -> NDArray[np.float64]:
    """(K,) m: each fix's residual vector against the median (per axis) of the residuals of
    the fixes in ``use`` within :data:`OUTLIER_WINDOW` of it (itself included)."""
    kept = np.flatnonzero(use)
    lo = np.searchsorted(t[kept], t - OUTLIER_WINDOW, side="left")
    hi = np.searchsorted(t[kept], t + OUTLIER_WINDOW, side="right")
    local = np.empty_like(residual)
    for i in range(t.size):
        near = kept[lo[i]:hi[i]]
        local[i] = np.median(residual[near], axis=0) if near.size else residual[i]
    return np.hypot(*(residual - local).T)


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
    at = {name: np.column_stack([np.interp(ft[inside], t, xy[:, 0]),
                                 np.interp(ft[inside], t, xy[:, 1])])
          for name, (t, xy) in series.items()}
    use = np.ones(n, dtype=bool)
    fits = {name: _aligned(name, a, ref, use) for name, a in at.items()}
    out.rmse_all = {name: _rms(r) for name, (_, _, r) in fits.items()}
    fix_t = ft[inside]
    for _ in range(OUTLIER_ROUNDS):
        far = np.ones(n, dtype=bool)
        for _, _, r in fits.values():
            d = _departures(fix_t, r, use)
            far &= d > max(OUTLIER_FACTOR * float(np.median(d[use])), OUTLIER_FLOOR)
        if not np.any(far & use) or np.count_nonzero(use & ~far) < 2:
            break
        use &= ~far
        fits = {name: _aligned(name, a, ref, use) for name, a in at.items()}
    out.outliers = int(n - np.count_nonzero(use))
    for name, (theta, shift, r) in fits.items():
        out.rmse[name] = _rms(r[use])
        c, s = np.cos(theta), np.sin(theta)
        out.gps_in_track_frame[name] = (ref - shift) @ np.array([[c, -s], [s, c]])
    return out


def _rms(residual: NDArray[np.float64]) -> float:
    """m: the root mean square of residual vectors' lengths."""
    return float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1))))
