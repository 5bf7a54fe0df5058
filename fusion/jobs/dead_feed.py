"""A dead odometry feed, said where it happened: stretches of consecutive odometry frames that
read zero while the EKF took them for encoder faults (the IMU showed motion; not fused).

The ``encoder_fault`` trust warning speaks only when such frames are a tenth of the run (then
the feed is the input, not a fault). An independent probe's 8 s dead feed in a 300 s run (2.7
% of its frames, the EKF riding through it as built to) was said by a counter alone; the
user could not tell when, for how long, nor that the pose had coasted on the motion model
there. :func:`dead_feed_notes` names each stretch of at least :data:`MIN_DEAD_FEED`, and
counts the shorter ones where they add up to as much.

Stretches are made of the frames themselves (a silence of more than :data:`GAP_PERIODS`
periods ends one: a gap is no zero reading), and a stretch counts when most of the fused rows
over it carry the EKF's ``encoder_fault`` flag (rows come at the IMU's rate, and a row carries
the flag of the last frame before it). Units: s, m/s.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from fusion.io.fused_csv import FUSED_CSV_COLUMNS

__all__ = ["MIN_DEAD_FEED", "dead_feed_notes"]

#: s: the shortest stretch listed (shorter ones are a few frames the EKF rides through; they
#: are counted together when they add up to this).
MIN_DEAD_FEED = 1.0
#: Stretches at most this many listed; the rest are counted.
MAX_LISTED = 5
#: Frames more than this many periods apart end a stretch (a few lost frames inside a dead
#: feed do not; a silence does: no frame is no zero reading).
GAP_PERIODS = 5.0
#: Share of a stretch's fused rows flagged encoder_fault for it to count.
FLAGGED_SHARE = 0.5

_FAULT = FUSED_CSV_COLUMNS.index("encoder_fault")
_SPEED = FUSED_CSV_COLUMNS.index("v")


def dead_feed_notes(frame_t: NDArray[np.float64], zero: NDArray[np.bool_],
                    table: NDArray[np.float64], period: float, what: str) -> list[str]:
    """One note for the dead-feed stretches of a fused run, or none: ``frame_t`` (M,) s the
    odometry frames' stamps (end of their period), ``zero`` (M,) those that read zero,
    ``table`` the fused rows (fused CSV columns, in time), ``period`` s the frames' period,
    ``what`` names the odometry ("wheel frames", "odometry twists (/odom)")."""
    t = np.asarray(frame_t, dtype=np.float64)
    zero = np.asarray(zero, dtype=bool)
    if not zero.any() or table.shape[0] == 0:
        return []
    idx = np.flatnonzero(zero)
    cut = (np.diff(idx) > 1) | (np.diff(t[idx]) > GAP_PERIODS * period)
    starts = idx[np.concatenate(([True], cut))]
    ends = idx[np.concatenate((cut, [True]))]
    rows_t = table[:, 0]
    found = []  # (first frame, length s, start s)
    for i0, i1 in zip(starts, ends, strict=True):
        begin, end = t[i0] - period, t[i1]  # the periods the frames close
        # the rows after the first frame's mid-period and up to one period past the last's
        rows = slice(np.searchsorted(rows_t, begin + 0.5 * period),
                     np.searchsorted(rows_t, end + 0.5 * period))
        flags = table[rows, _FAULT]
        if flags.size and np.mean(flags > 0.0) >= FLAGGED_SHARE:
            found.append((rows.start, end - begin, begin))
    long = [f for f in found if f[1] >= MIN_DEAD_FEED]
    short = [f for f in found if f[1] < MIN_DEAD_FEED]
    short_total = sum(f[1] for f in short)
    if not long and short_total < MIN_DEAD_FEED:
        return []
    parts = [f"{length:.1f} s from t = {start:.3f} s (v {table[row, _SPEED]:+.2f} m/s there)"
             for row, length, start in long[:MAX_LISTED]]
    if len(long) > MAX_LISTED:
        parts.append(f"{len(long) - MAX_LISTED} more of 1 s or longer")
    if short and short_total >= MIN_DEAD_FEED:
        parts.append(f"{len(short)} shorter one(s), {short_total:.1f} s in all")
    return [f"the {what} read zero while the IMU showed the robot moving: "
            f"{'; '.join(parts)}; not fused (flagged encoder_fault), the pose coasted on the "
            "motion model there with a growing covariance: a dead encoder feed (wiring, the "
            "chassis link), or the robot moved without its wheels turning (carried, pushed)"]
