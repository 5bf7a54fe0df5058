"""A replay's IMU stamps put on the odometry's clock when the two disagree
(:func:`fusion.calibration.time_offset.estimate_imu_lag`), or by the lag the user gives
(``fusion replay --imu-lag``).

The lag moved is the estimate less what a well-stamped log shows: a wheel frame is the mean
rate over the period it closes, which the pipeline already places half a period before its
stamp, and which the estimate reads as the IMU half a period early (-5 to -16 ms on the
black-box simulator's runs); a twist is taken at its stamp. Up to :func:`lag_limit` nothing
is moved: a few tens of ms cost nothing measurable (the terrain bag's IMU 0.3 s late: 1.49 m
of GPS RMSE against 1.46). Beyond it the IMU's stamps are moved with a note, when at least
two pieces of the run line up at the same lag; when they do not (a driver restarted with
another lag, turns that repeat at one period), or when the run is too short or turned too
little to check on two pieces, nothing is moved and the note says why. A piece keeps
another lag if its own is further than twice that limit from the run's, or further than
the limit and fits it clearly better (:data:`FIT_Z`): slipping wheels move a piece's peak
without that.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from fusion.calibration.time_offset import ImuLag, estimate_imu_lag
from fusion.io.odometry_motion import message_period
from fusion.jobs.streams import Streams

__all__ = ["FIT_Z", "LAG_LIMIT", "LagChoice", "choose_imu_lag", "lag_limit", "shifted"]

#: s: the least lag moved, whatever the streams' rates.
LAG_LIMIT = 0.1
#: How much worse (in Fisher's z, atanh of the correlation) a piece's rates must line up at
#: the whole run's lag than at the piece's own before that piece counts as keeping another
#: lag. Slipping wheels move one piece's peak without making the run's lag fit it worse: on
#: the physics simulator's 90 s runs (seeds 0, 1) pieces peaked 0.12 s from the rest, at
#: 0.959 against 0.948 at the run's lag (z 0.12); a driver restarted 0.8 s later loses 1.5
#: on a clean odometry (a noisy one less: hence the bound of twice the limit as well).
FIT_Z = 1.0


@dataclass(frozen=True)
class LagChoice:
    """What a replay does with the IMU's stamps.

    Attributes:
        lag: s taken off the IMU's stamps (0: left as they are).
        note: what to tell the user ("" for nothing).
        estimate: the estimate it rests on (None: given, or none found).
    """

    lag: float = 0.0
    note: str = ""
    estimate: ImuLag | None = None


def lag_limit(streams: Streams) -> float:
    """s: lags up to this are left alone: :data:`LAG_LIMIT`, or two intervals of the slower
    stream (the IMU's or the odometry's median interval) if that is longer."""
    periods = [_period(t) for t in (streams.imu_t, streams.wheel_t, streams.twist_t)]
    return max([LAG_LIMIT, *(2.0 * p for p in periods if p is not None)])


def choose_imu_lag(streams: Streams, chassis, given: float | None = None) -> LagChoice:
    """What to take off the IMU's stamps (module docstring). ``given``: the user's lag
    (``--imu-lag``), taken as it is; None: estimated. ``chassis``: the wheel frames'
    geometry. ValueError for a given lag that is not finite or without IMU samples."""
    if given is not None:
        if not math.isfinite(given):
            raise ValueError(f"--imu-lag must be a finite number of s, got {given!r}")
        if not streams.has_imu:
            raise ValueError("--imu-lag: there are no IMU samples to move")
        return LagChoice(float(given), f"IMU stamps moved by {-given:+.3f} s onto the "
                         "odometry's clock (--imu-lag)" if given else "")
    odometry = streams.odometry_rates(chassis) if streams.has_imu else None
    if odometry is None:
        return LagChoice()
    t, _, w = odometry
    est = _estimate(streams, t, w)
    if est is None:
        return LagChoice()
    # a wheel frame's rate is its period's mean: read as half a period late (module docstring)
    expected = -0.5 * (_period(streams.wheel_t) or 0.0) if streams.has_wheels else 0.0
    lag = est.lag - expected
    limit = lag_limit(streams)
    pieces = (f"pieces of {est.piece:.0f} s line up at "
              + ", ".join(f"{x - expected:+.3f}" for x in est.piece_lags) + " s")
    if _pieces_disagree(est, limit):
        return LagChoice(0.0, f"the IMU's and the odometry's stamps do not keep one lag "
                         f"through the run ({pieces}: a driver restarted with another lag, "
                         "a clock that stepped, or turns that repeat at one period): not "
                         "moved; --imu-lag S moves every IMU stamp by S, and a bag's record "
                         "times (--stamps bag) keep one clock through a restart", est)
    if not abs(lag) > limit:
        return LagChoice(estimate=est)
    apart = _apart(lag)
    if len(est.piece_lags) < 2:
        return LagChoice(0.0, f"{apart} (their yaw rates line up best there, correlation "
                         f"{est.correlation:.3f}), but the run is too short or turned too "
                         f"little to check it on two pieces of {est.piece:.0f} s: not moved; "
                         f"--imu-lag {lag:.3f} moves them", est)
    return LagChoice(lag, f"{apart} (their yaw rates line up best there: correlation "
                     f"{est.correlation:.3f}; {pieces}): the IMU's moved onto the odometry's "
                     "clock (--imu-lag 0 keeps them)", est)


def _pieces_disagree(est: ImuLag, limit: float) -> bool:
    """Whether a piece of the run keeps another lag than the whole run's: its own lies more
    than twice ``limit`` (s: what is never moved, :func:`lag_limit`) away, or more than
    ``limit`` and lines up clearly better (:data:`FIT_Z`) than the run's lag does for it.
    Why the first: the drop of the correlation shrinks with the odometry's noise, and a
    review's driver restart from 0 to 0.5 s late, with 0.05 rad/s of noise on a 20 Hz
    odometry, passed the z test: every stamp was moved by the mean, 0.25 s."""
    if len(est.piece_fits) != len(est.piece_lags):
        raise ValueError("ImuLag without piece_peaks and piece_fits (estimate_imu_lag gives them)")
    for lag, peak, fit in zip(est.piece_lags, est.piece_peaks, est.piece_fits):
        if abs(lag - est.lag) <= limit:
            continue
        if abs(lag - est.lag) > 2.0 * limit:
            return True
        if not math.isfinite(fit):  # no correlation at the run's lag (out of the search,
            return True  # too few points or no variance there)
        peak, fit = (min(c, 1.0 - 1e-12) for c in (peak, fit))
        if math.atanh(peak) - math.atanh(fit) > FIT_Z:
            return True
    return False


def shifted(streams: Streams, lag: float) -> Streams:
    """``streams`` with ``lag`` s taken off the IMU's stamps (itself for 0)."""
    if not lag or not streams.has_imu:
        return streams
    return dataclasses.replace(streams, imu_t=streams.imu_t - lag)


def _apart(lag: float) -> str:
    """The lag in words, blaming neither clock."""
    side = "behind" if lag > 0 else "ahead of"
    return f"the IMU's stamps ran {abs(lag):.3f} s {side} the odometry's"


def _period(t) -> float | None:
    """s: the message period of stamps ``t`` (:func:`fusion.io.odometry_motion.message_period`;
    None for fewer than two)."""
    p = message_period(t) if t is not None else 0.0
    return p if math.isfinite(p) and p > 0 else None


def _estimate(streams: Streams, t, w) -> ImuLag | None:
    """The lag about the accelerometer's up; where the accelerometer does not read gravity,
    about whichever IMU axis (either sign) lines up best with the odometry."""
    if not streams.level_note():
        return estimate_imu_lag(streams.imu_t, streams.gyro, np.mean(streams.accel, axis=0),
                                t, w)
    found = [estimate_imu_lag(streams.imu_t, streams.gyro, sign * axis, t, w)
             for axis in np.eye(3) for sign in (1.0, -1.0)]
    found = [f for f in found if f is not None]
    return max(found, key=lambda f: f.correlation, default=None)
