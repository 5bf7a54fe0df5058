"""A dead odometry feed, said where it happened: stretches of a fused run whose odometry read
zero while the IMU showed motion (the EKF's encoder faults, not fused).

The ``encoder_fault`` trust warning speaks only when such frames are a tenth of the run (then
the feed is the input, not a fault). An independent probe's 8 s dead feed in a 300 s run (2.7
% of its frames, the EKF riding through it as built to) was said by a counter alone; the
user could not tell when, for how long, nor that the pose had coasted on its last speed
there. :func:`dead_feed_notes` names each stretch of at least :data:`MIN_DEAD_FEED`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from fusion.io.fused_csv import FUSED_CSV_COLUMNS

__all__ = ["MIN_DEAD_FEED", "dead_feed_notes"]

#: s: the shortest stretch said (shorter ones are a few frames the EKF rides through).
MIN_DEAD_FEED = 1.0
#: Stretches at most this many listed; the rest are counted.
MAX_LISTED = 5

_FAULT = FUSED_CSV_COLUMNS.index("encoder_fault")
_SPEED = FUSED_CSV_COLUMNS.index("v")


def dead_feed_notes(table: NDArray[np.float64], period: float, what: str) -> list[str]:
    """One note for the stretches of the fused ``table`` (fused CSV columns, rows in time)
    flagged ``encoder_fault`` for at least :data:`MIN_DEAD_FEED` s, gaps of up to two
    ``period`` s between flagged rows bridged; ``what`` names the odometry ("wheel frames",
    "twists"). Empty when there is none."""
    t = table[:, 0]
    flagged = np.flatnonzero(table[:, _FAULT] > 0.0)
    if flagged.size < 2:
        return []
    breaks = np.flatnonzero(np.diff(t[flagged]) > 2.0 * period)
    starts = np.concatenate(([0], breaks + 1))
    ends = np.concatenate((breaks, [flagged.size - 1]))
    spans = [(flagged[s], flagged[e]) for s, e in zip(starts, ends, strict=True)
             if t[flagged[e]] - t[flagged[s]] >= MIN_DEAD_FEED]
    if not spans:
        return []
    listed = ", ".join(
        f"{t[e] - t[s]:.1f} s from t = {t[s]:.3f} s (speed held at {table[s, _SPEED]:+.2f} "
        f"m/s)" for s, e in spans[:MAX_LISTED])
    more = f" and {len(spans) - MAX_LISTED} more" if len(spans) > MAX_LISTED else ""
    return [f"the {what} read zero while the IMU showed the robot moving: {listed}{more}; "
            "not fused (flagged encoder_fault), the pose coasted on the motion model there "
            "with a growing covariance: a dead encoder feed (wiring, the chassis link)"]
