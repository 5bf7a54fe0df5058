"""How late the IMU's stamps are against the odometry's, from the turns both see.

Two drivers stamp their messages on their own: an IMU driver that stamps when its serial
buffer drains, a wheel controller that stamps when a frame is parsed, a bag recorded from two
machines. Fused with a lag, the gyro's turns meet the odometry's a moment apart: the EKF
calls the mismatch slip and the heading takes the turns late. On the terrain outdoor bag an
IMU stamped 1 s late cost 2.42 m of GPS RMSE instead of 1.46, and nothing said so.

:func:`estimate_imu_lag` finds the lag that best lines up the gyro's yaw rate (its rate
about ``up``: the accelerometer's mean, or an axis the caller found) with the odometry's:
both headings are integrated, sampled on one grid (:data:`GRID` s), differenced over the
same window (so a 10 Hz odometry and a 200 Hz gyro are smoothed alike), and the Pearson
correlation of the two rates is taken for every lag up to :data:`MAX_LAG` (a bias and a scale
error drop out; a parabola through the peak refines it below the grid). The correlation is
signed: ``up`` fixes which way the gyro turns, so a robot weaving at a steady period does not
line up against its own mirror image half a period away. A peak on the edge of the search is
no estimate (the lag is longer, or there is none). The run is also cut into pieces
(:func:`piece_length`); each piece that turned at least :data:`PIECE_TURN` gets its own lag,
its correlation there and at the whole run's lag: whether one lag fits the whole run (a
driver restarted with another lag, a weave whose period aliases).

Each sample is taken as the rate at its stamp: a wheel frame or a twist that is the mean over
the interval it closes reads as late by about half that interval.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.integrate import cumulative_trapezoid
from scipy.signal import correlate

from fusion.calibration.gyro_axes import MIN_TURN

__all__ = ["GRID", "MAX_LAG", "MIN_CORRELATION", "ImuLag", "estimate_imu_lag",
           "piece_length"]

#: s: the grid both headings are sampled on (the lag's resolution before the parabola).
GRID = 0.01
#: s: the largest lag searched, either way.
MAX_LAG = 3.0
#: s: the longest piece the run is cut into; a shorter run is cut into four.
PIECE = 60.0
#: s: the shortest piece.
MIN_PIECE = 20.0
#: The least correlation at the peak for a lag to mean anything (the two rates then follow
#: each other closely; below, the gyro's axis or the odometry is not the robot's turning).
MIN_CORRELATION = 0.8
#: rad: the odometry's turns a piece needs for its own lag (the whole run needs
#: :data:`fusion.calibration.gyro_axes.MIN_TURN`): a quarter turn has onsets enough to place.
PIECE_TURN = 0.5 * math.pi
#: s: a stream silent for longer than this (or three of its intervals, if longer) has a gap;
#: the grid points whose window touches it are not used.
GAP = 1.0


@dataclass(frozen=True)
class ImuLag:
    """The IMU's stamps against the odometry's.

    Attributes:
        lag: s, how much later the IMU stamps a motion than the odometry does (positive: the
            IMU's stamps are late; subtract it from them to put them on the odometry's clock).
        correlation: of the two yaw rates at ``lag`` (signed).
        piece_lags: s, the lags of the pieces that turned enough and correlate.
        piece: s, the pieces' length.
        window: s, the window both rates were averaged over.
        piece_peaks: the correlation of each of those pieces at its own lag.
        piece_fits: the correlation of each of those pieces at the whole run's ``lag``.
    """

    lag: float
    correlation: float
    piece_lags: tuple[float, ...]
    piece: float
    window: float
    piece_peaks: tuple[float, ...] = ()
    piece_fits: tuple[float, ...] = ()

    @property
    def spread(self) -> float:
        """s: the range of the pieces' lags (0 with fewer than two)."""
        return max(self.piece_lags) - min(self.piece_lags) if len(self.piece_lags) > 1 else 0.0


def piece_length(span: float) -> float:
    """s: the pieces a run of ``span`` s is cut into: :data:`PIECE`, or a quarter of a
    shorter run, but not below :data:`MIN_PIECE`."""
    return max(MIN_PIECE, min(PIECE, span / 4.0))


def estimate_imu_lag(imu_t: ArrayLike, gyro: ArrayLike, up: ArrayLike, odom_t: ArrayLike,
                     odom_w: ArrayLike) -> ImuLag | None:
    """The lag of the IMU's stamps behind the odometry's (module docstring); None when the
    streams share too little time (four times :data:`MAX_LAG`), the robot turned less than
    :data:`fusion.calibration.gyro_axes.MIN_TURN`, the rates do not follow each other at
    any lag (:data:`MIN_CORRELATION`), or the best lag is at the edge of the search.

    Args:
        imu_t: (N,) s, increasing. gyro: (N, 3) rad/s, IMU frame.
        up: (3,) the IMU frame's up (any length): the gyro's rate about it turns as the
            odometry's yaw rate does.
        odom_t: (M,) s, increasing. odom_w: (M,) rad/s, the odometry's yaw rate.
    """
    t = np.asarray(imu_t, dtype=float)
    u = np.asarray(up, dtype=float)
    norm = float(np.linalg.norm(u))
    if t.size < 2 or not (math.isfinite(norm) and norm > 0):
        return None
    rate = np.asarray(gyro, dtype=float) @ (u / norm)
    s = np.asarray(odom_t, dtype=float)
    w = np.asarray(odom_w, dtype=float)
    ok = np.isfinite(t) & np.isfinite(rate)
    t, rate = t[ok], rate[ok]
    ok = np.isfinite(s) & np.isfinite(w)
    s, w = s[ok], w[ok]
    if t.size < 2 or s.size < 2:
        return None
    t0, t1 = max(t[0], s[0]), min(t[-1], s[-1])
    if not t1 - t0 > 4.0 * MAX_LAG:
        return None
    # both rates as differences of their integrated headings over one window: the slower
    # stream's two intervals (a 10 Hz odometry's 0.2 s), so neither is sharper than the other
    period = max(float(np.median(np.diff(t))), float(np.median(np.diff(s))))
    half = max(1, round(period / GRID))
    gap = max(GAP, 3.0 * period)
    grid = np.arange(t0, t1, GRID)
    a = _windowed_rate(t, rate, grid, half)
    b = _windowed_rate(s, w, grid, half)
    valid = _covered(t, grid, half, gap) & _covered(s, grid, half, gap)
    if _turn(b, valid) < MIN_TURN:
        return None
    lag, corr = _best_lag(a, b, valid)
    if lag is None or corr < MIN_CORRELATION:
        return None
    piece = piece_length(t1 - t0)
    n_piece = int(piece / GRID)
    lags, peaks, fits = [], [], []
    for start in range(0, grid.size - n_piece + 1, n_piece):
        sl = slice(start, start + n_piece)
        if _turn(b[sl], valid[sl]) < PIECE_TURN:
            continue
        corr_piece = _correlations(a[sl], b[sl], valid[sl])
        piece_lag, piece_corr = _peak(corr_piece)
        if piece_lag is not None and piece_corr >= MIN_CORRELATION:
            lags.append(piece_lag)
            peaks.append(piece_corr)
            fits.append(_correlation_at(corr_piece, lag))
    return ImuLag(lag, corr, tuple(lags), piece, 2 * half * GRID, tuple(peaks), tuple(fits))


def _turn(w: NDArray[np.float64], valid: NDArray[np.bool_]) -> float:
    """rad: the turns of the grid rates ``w`` over the valid points."""
    return float(np.sum(np.abs(w[valid]))) * GRID


def _windowed_rate(t: NDArray[np.float64], rate: NDArray[np.float64],
                   grid: NDArray[np.float64], half: int) -> NDArray[np.float64]:
    """The mean of ``rate`` over ``[g - half, g + half]`` grid steps around each grid point,
    from its integral (rad/s)."""
    heading = cumulative_trapezoid(rate, t, initial=0.0)
    lo = np.interp(grid - half * GRID, t, heading)
    hi = np.interp(grid + half * GRID, t, heading)
    return (hi - lo) / (2 * half * GRID)


def _covered(t: NDArray[np.float64], grid: NDArray[np.float64], half: int, gap: float
             ) -> NDArray[np.bool_]:
    """Grid points whose window lies inside the stream and touches no interval longer than
    ``gap`` s (the window is shorter than ``gap``: a gap it overlaps holds one of its ends)."""
    lo, hi = grid - half * GRID, grid + half * GRID
    out = (lo >= t[0]) & (hi <= t[-1])
    for edge in (lo, hi):
        k = np.clip(np.searchsorted(t, edge), 1, t.size - 1)
        out &= t[k] - t[k - 1] <= gap
    return out


def _best_lag(a: NDArray[np.float64], b: NDArray[np.float64], valid: NDArray[np.bool_]
              ) -> tuple[float | None, float]:
    """The shift of ``a`` (s) that best matches ``b`` (``a[i + k]`` with ``b[i]``) by the
    Pearson correlation over the points valid in both, refined by a parabola through the
    peak, and that correlation; ``(None, 0)`` for a peak on the edge of the search."""
    return _peak(_correlations(a, b, valid))


def _peak(corr: NDArray[np.float64]) -> tuple[float | None, float]:
    """:func:`_best_lag` of the correlations ``corr`` (:func:`_correlations`)."""
    kmax = corr.size // 2
    if not np.any(np.isfinite(corr)):
        return None, 0.0
    j = int(np.nanargmax(corr))
    if j == 0 or j == corr.size - 1:
        return None, 0.0
    shift = float(j - kmax)
    c0, c1, c2 = corr[j - 1], corr[j], corr[j + 1]
    den = c0 - 2.0 * c1 + c2
    if np.isfinite(c0) and np.isfinite(c2) and den < 0:
        shift += 0.5 * float(c0 - c2) / float(den)
    return shift * GRID, float(corr[j])


def _correlation_at(corr: NDArray[np.float64], lag: float) -> float:
    """The correlation at a shift of ``lag`` s of the correlations ``corr``
    (:func:`_correlations`), interpolated between the grid's shifts; NaN outside the search
    (or where ``corr`` is)."""
    kmax = corr.size // 2
    return float(np.interp(lag / GRID, np.arange(-kmax, kmax + 1), corr,
                           left=np.nan, right=np.nan))


def _correlations(a: NDArray[np.float64], b: NDArray[np.float64], valid: NDArray[np.bool_]
                  ) -> NDArray[np.float64]:
    """(2 kmax + 1,) the Pearson correlation of ``a[i + k]`` with ``b[i]`` over the points
    valid in both, for the shifts ``k = -kmax..kmax`` grid steps (up to :data:`MAX_LAG`, and
    a quarter of the series); NaN where fewer than 10 points or no variance."""
    n = a.size
    kmax = min(int(MAX_LAG / GRID), n // 4)
    m = valid.astype(float)
    av, bv = np.where(valid, a, 0.0), np.where(valid, b, 0.0)

    def xc(x, y):  # sum_i x[i + k] y[i] for k = -kmax..kmax (FFT)
        return correlate(x, y, mode="full", method="fft")[n - 1 - kmax:n + kmax]

    count = np.rint(xc(m, m))
    sa, sb, sab = xc(av, m), xc(m, bv), xc(av, bv)
    saa, sbb = xc(av * av, m), xc(m, bv * bv)
    with np.errstate(divide="ignore", invalid="ignore"):
        cov = sab - sa * sb / count
        var = (saa - sa * sa / count) * (sbb - sb * sb / count)
        return np.where((count >= 10) & (var > 0), cov / np.sqrt(var), np.nan)
