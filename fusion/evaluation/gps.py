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

A fix stamped when it reached the host, not at its epoch, is late: a receiver's solution and
its serial line take 0.1-1 s, an NMEA bridge or a busy driver more. Every track then trails
the fixes, by the speed times the lag along the path, which the alignment cannot take out in
the turns: the probe's bag above with 1 Hz fixes stamped 2.5 s late printed 2.88 m for the
fused track (1.55 m on time). :func:`compare_with_fixes` searches the fixes' lag within
:data:`LAG_MAX` either side, the one that fits the tracks best together (the mean of their
RMSEs' logarithms: each track's relative change counts, so a track tens of metres off does not
outweigh a good one), each fitted with a rotation, a shift AND a scale for this search
(:func:`_scaled_fit_rms`: a distance scale error, which the fused track, the bag's odometry
and the gyro-at-stops track all share through the wheels' speed, stretches the path as a lag
would: under a rigid fit on-time fixes read as -1.1 s late for a 3 % scale, review). It
compares at that lag where it is :data:`LAG_MIN` or more and lowers that mean RMSE to
:data:`LAG_GAIN` or less; the figures are still after one SE(2) alignment each, and those at
the stamps as recorded stay in :attr:`GpsComparison.rmse_at_stamps`. A best lag at the
search's edge is not applied (:attr:`GpsComparison.lag_beyond` says when it gains as much).
That bag now prints 1.50 m (lag 2.75 s); 1.0 and -1.5 s give 1.54 m (1.26 and -1.24 s), 0.5 s
is not applied (1.67 m); on time, 1.55 m, none. Under a scale error shared by the tracks the
rigid figures at the right lag can read higher than at the stamps, where the alignment had
traded the one error against the other; the lag found is still the epochs', and both are
printed (review). The lag is fitted on the tracks it scores, one parameter over hundreds of
fixes. The odometry's own clock running ahead of the GPS would look the same, and is said the
same way (the lag is printed).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import minimize_scalar

from fusion.evaluation.trajectory import se2_alignment
from fusion.geometry.geodesy import geodetic_to_enu

__all__ = ["LAG_GAIN", "LAG_MAX", "LAG_MIN", "LAG_MIN_FIXES", "OUTLIER_FACTOR",
           "OUTLIER_FLOOR", "OUTLIER_ROUNDS", "OUTLIER_WINDOW", "GpsComparison",
           "compare_with_fixes", "fixes_to_enu"]

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
#: s: the fixes' lag is searched within this either side (a receiver's latency and its
#: driver's: up to a second or two; a clock off by more is another fault, named elsewhere).
LAG_MAX = 3.0
#: s: a lag below this is not applied (within a 5-10 Hz receiver's period: no latency to
#: speak of, and what such a fit finds there is mostly the fixes' noise).
LAG_MIN = 0.2
#: The lag is applied where it lowers the tracks' RMSE (their geometric mean) to this
#: fraction of the on-stamp figure or less: 5 %, beyond what one fitted parameter gains
#: from noise over hundreds of fixes.
LAG_GAIN = 0.95
#: Fixes, at least, inside every track's span at every lag searched; fewer: no search.
LAG_MIN_FIXES = 20
#: s: the grid the lag is first searched on (a Jackal's 2 m/s moves 0.1 m in it).
_LAG_STEP = 0.05
#: m: an RMSE is taken as at least this in the lag's objective (a track that fits the
#: fixes exactly would give the logarithm of 0).
_RMSE_FLOOR = 0.01
#: m: and as at most this (a lag that reads a track's sample that is not finite: the worst
#: fit, kept finite for the search's arithmetic).
_RMSE_CAP = 1e12


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
        lag: s, how late the fixes' stamps were taken to be (each compared with the tracks
            at its stamp less this): 0 unless the search found one (module docstring).
        rmse_at_stamps: per track name, the RMSE with the fixes at their stamps as
            recorded (outliers left out); empty where ``lag`` is 0 (it is ``rmse`` then).
        lag_beyond: the fixes fit the tracks better :data:`LAG_MAX` off their stamps than on
            them, and the best lag lies beyond (not applied: another clock, most likely).
    """

    rmse: dict[str, float] = field(default_factory=dict)
    compared: int = 0
    span: tuple[float, float] = (0.0, 0.0)
    gps_in_track_frame: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    outliers: int = 0
    rmse_all: dict[str, float] = field(default_factory=dict)
    lag: float = 0.0
    rmse_at_stamps: dict[str, float] = field(default_factory=dict)
    lag_beyond: bool = False


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
                       tracks: dict[str, tuple[ArrayLike, ArrayLike]],
                       find_lag: bool = True) -> GpsComparison:
    """Compare each of ``tracks`` (name -> (t (M,) s, xy (M, 2) m), t increasing) with the fixes
    ``fix_en`` ((N, 2) east, north m at ``fix_t`` s, increasing) inside every track's span;
    with ``find_lag``, at the fixes' lag where one is found (module docstring).

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
    on_stamps, kept = _compared(ft, fen, series, 0.0)
    lag, beyond = _fix_lag(ft, fen, series, kept) if find_lag else (0.0, False)
    on_stamps.lag_beyond = beyond
    if lag == 0.0:
        return on_stamps
    out, _ = _compared(ft, fen, series, lag)
    out.rmse_at_stamps = dict(on_stamps.rmse)
    return out


def _compared(ft: NDArray[np.float64], fen: NDArray[np.float64],
              series: dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]],
              lag: float) -> tuple[GpsComparison, NDArray[np.bool_]]:
    """``(comparison, kept)``: the comparison with each fix taken at its stamp ``ft`` less
    ``lag`` s (outliers left out, module docstring; ``span`` in the fixes' stamps), and which
    of ``ft`` it compared and kept (not outliers)."""
    start = max(t[0] for t, _ in series.values())
    end = min(t[-1] for t, _ in series.values())
    at_t = ft - lag
    inside = (at_t >= start) & (at_t <= end)
    n = int(np.count_nonzero(inside))
    if n < 2:
        fixes = f"{ft[0]:.3f}-{ft[-1]:.3f} s" if ft.size else "none"
        raise ValueError(f"{n} of the {ft.size} GPS fixes (stamped {fixes}) lie inside the "
                         f"odometry's span {start:.3f}-{end:.3f} s; need at least 2 (are "
                         f"the stamps on another clock?)")
    ref = fen[inside]
    out = GpsComparison(compared=n, span=(float(ft[inside][0]), float(ft[inside][-1])),
                        lag=lag)
    at = {name: _track_at(t, xy, at_t[inside]) for name, (t, xy) in series.items()}
    use = np.ones(n, dtype=bool)
    fits = {name: _aligned(name, a, ref, use) for name, a in at.items()}
    out.rmse_all = {name: _rms(r) for name, (_, _, r) in fits.items()}
    fix_t = at_t[inside]
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
    kept = np.zeros(ft.size, dtype=bool)
    kept[np.flatnonzero(inside)[use]] = True
    for name, (theta, shift, r) in fits.items():
        out.rmse[name] = _rms(r[use])
        c, s = np.cos(theta), np.sin(theta)
        out.gps_in_track_frame[name] = (ref - shift) @ np.array([[c, -s], [s, c]])
    return out, kept


def _track_at(t: NDArray[np.float64], xy: NDArray[np.float64],
              when: NDArray[np.float64]) -> NDArray[np.float64]:
    """(K, 2) m: the track ``xy`` at times ``t`` interpolated linearly at ``when``."""
    return np.column_stack([np.interp(when, t, xy[:, 0]), np.interp(when, t, xy[:, 1])])


def _fix_lag(ft: NDArray[np.float64], fen: NDArray[np.float64],
             series: dict[str, tuple[NDArray[np.float64], NDArray[np.float64]]],
             kept: NDArray[np.bool_]) -> tuple[float, bool]:
    """``(lag s, beyond)``: the fixes' lag that fits every track best (module docstring), or 0
    where none is :data:`LAG_MIN` or more and gains :data:`LAG_GAIN`, or where the best is at
    the search's edge (``beyond`` True when the edge gains that much); searched on a grid of
    :data:`_LAG_STEP` and refined between its neighbours, over the fixes ``kept`` on their
    stamps (not outliers) that lie inside every track's span at every lag searched."""
    start = max(t[0] for t, _ in series.values()) + LAG_MAX
    end = min(t[-1] for t, _ in series.values()) - LAG_MAX
    use = kept & (ft >= start) & (ft <= end)
    if np.count_nonzero(use) < LAG_MIN_FIXES:
        return 0.0, False
    when, ref = ft[use], fen[use]

    def objective(lag: float) -> float:
        """The mean over the tracks of log(RMSE), each fitted with a scale at this lag."""
        return float(np.mean([np.log(np.clip(_scaled_fit_rms(_track_at(t, xy, when - lag),
                                                             ref), _RMSE_FLOOR, _RMSE_CAP))
                              for t, xy in series.values()]))

    grid = np.linspace(-LAG_MAX, LAG_MAX, round(2 * LAG_MAX / _LAG_STEP) + 1)
    scores = np.array([objective(float(g)) for g in grid])
    k = int(np.argmin(scores))
    if k in (0, grid.size - 1):  # at the search's edge: beyond it, or no minimum to place
        return 0.0, bool(scores[k] - objective(0.0) <= np.log(LAG_GAIN))
    best = minimize_scalar(objective, bounds=(grid[k - 1], grid[k + 1]), method="bounded",
                           options={"xatol": 1e-3})
    lag, score = (float(best.x), float(best.fun)) if best.fun < scores[k] else \
        (float(grid[k]), float(scores[k]))
    if abs(lag) < LAG_MIN or score - objective(0.0) > np.log(LAG_GAIN):
        return 0.0, False
    return lag, False


def _scaled_fit_rms(track: NDArray[np.float64], ref: NDArray[np.float64]) -> float:
    """m: the RMSE of ``ref`` (K, 2) against ``track`` (K, 2) after the rotation, scale and
    shift that fit it best (complex least squares), inf where ``track`` is not finite. The
    lag's objective: the tracks' distance scale error (a wheel radius or speed_ratio a few
    per cent off, which the fused track, the bag's odometry and the gyro-at-stops track all
    share) stretches the path as a lag along it would, and under a rigid fit read as one
    (on-time fixes: -1.1 s for a 3 % scale, a true 2 s lag found at 0.2 s under 5 %)."""
    if not np.isfinite(track).all():
        return math.inf
    a = (track - track.mean(axis=0)) @ np.array([1.0, 1.0j])
    b = (ref - ref.mean(axis=0)) @ np.array([1.0, 1.0j])
    power = float(np.vdot(a, a).real)
    scale = np.vdot(a, b) / power if power > 0.0 else 0.0
    return float(np.sqrt(np.mean(np.abs(b - scale * a) ** 2)))


def _rms(residual: NDArray[np.float64]) -> float:
    """m: the root mean square of residual vectors' lengths."""
    return float(np.sqrt(np.mean(np.sum(residual ** 2, axis=1))))
