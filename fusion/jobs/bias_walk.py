"""A gyro bias that walks faster than ``[ekf] bias_psd`` says, read from a replay's own stops.

The EKF models the gyro bias as a random walk of ``bias_psd`` ((rad/s)^2/s; default
(1e-4)^2, which the bundled real MPU6050's 100 s at rest fits). A chip warming up after
power-on, or one in a changing temperature, drifts faster: its bias moves between two stops by
more than that walk allows, the filter holds the old bias while driving, and the heading
takes the difference (an independent simulator's warm-up of 0.4 deg/s over a minute: the
fused yaw 2-6 deg above what the gyro's scale leaves).

Each stop measures the bias to a few hundredths of a deg/s (zero-velocity updates). A
replay has them all: :func:`fit_bias_walk` takes the bias at the end of every stop of at
least :data:`fusion.jobs.moving_start.MIN_STOP` and tests the changes between consecutive
stops against the configured walk (chi-square of their normalised squares, each with its
two ends' variances and :data:`STOP_BIAS_STD`); where the configured walk is rejected at
:data:`SIGNIFICANCE`, over all stops and with any one of them left out, the walk's power
spectral density that makes the changes most likely (maximum likelihood over
``[bias_psd, MAX_RAISE * bias_psd]``) is what
:func:`fusion.jobs.replay.fuse_streams` fuses the log with again, with a note. Never lowered:
a bias that walks slower than configured costs little, and the default is a real chip's.
Not a tuned value: the log's own stops give it, and it is said.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize_scalar
from scipy.stats import chi2

from fusion.jobs.moving_start import MIN_STOP, STOP_MERGE_GAP

__all__ = ["MAX_RAISE", "MIN_INTERVALS", "SIGNIFICANCE", "STOP_BIAS_STD", "BiasWalk",
           "fit_bias_walk"]

#: The configured walk is rejected when the stops' bias changes are this unlikely under it.
SIGNIFICANCE = 0.01
#: Bias changes (stops less one) the test needs: the walk must be rejected with any one stop
#: left out too (one stop's bias can be off: a stop on a slope, a slow creep that the
#: odometry read as a stop), which leaves one change fewer.
MIN_INTERVALS = 3
#: rad/s: added to each stop's own bias variance (the filter's, which assumes its model, and
#: a stop's bias state can lag its readings a little): 3 s at rest at 200 Hz measure the
#: bias to about 0.01 deg/s (issue 11).
STOP_BIAS_STD = math.radians(0.01)
#: The largest factor the walk is raised by.
MAX_RAISE = 1e4


@dataclass(frozen=True)
class BiasWalk:
    """What :func:`fit_bias_walk` found.

    Attributes:
        psd: (rad/s)^2/s, the walk that fits the stops best (at least ``configured``).
        configured: (rad/s)^2/s, the walk the replay was fused with.
        changes: the number of bias changes between consecutive stops tested.
        p_value: how likely changes at least this large are under ``configured``: the
            largest of that chance over all stops and over all but any one of them.
        largest: rad/s, the largest change, and ``over`` s, the time it took.
    """

    psd: float
    configured: float
    changes: int
    p_value: float
    largest: float
    over: float

    @property
    def rejected(self) -> bool:
        """Whether the configured walk is rejected (:data:`SIGNIFICANCE`)."""
        return self.p_value < SIGNIFICANCE and self.psd > self.configured

    def note(self, fused_again: bool) -> str:
        """One sentence for the user."""
        how = ("the log was fused again with it" if fused_again else
               "a live run would follow it")
        return (f"the gyro bias moved between stops faster than [ekf] bias_psd = "
                f"{self.configured:.3g} allows (by up to {math.degrees(self.largest):.3f} "
                f"deg/s in {self.over:.0f} s; {self.changes} changes, chance "
                f"{self.p_value:.1g}): a chip warming up or in a changing temperature; the "
                f"walk its {self.changes + 1} stops fit best is bias_psd = {self.psd:.3g}, "
                f"and {how} (set it in robot.toml's [ekf] to keep it)")


def _stop_ends(t: NDArray[np.float64], zupt: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """(first, last) row of every stop: zero-velocity rows less than
    :data:`fusion.jobs.moving_start.STOP_MERGE_GAP` apart, lasting :data:`MIN_STOP` or more."""
    rows = np.flatnonzero(zupt)
    if rows.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(t[rows]) > STOP_MERGE_GAP)
    firsts = np.concatenate([[rows[0]], rows[breaks + 1]])
    lasts = np.concatenate([rows[breaks], [rows[-1]]])
    return [(int(a), int(b)) for a, b in zip(firsts, lasts, strict=True)
            if t[b] - t[a] >= MIN_STOP]


def fit_bias_walk(t: NDArray[np.float64], bias: NDArray[np.float64],
                  bias_var: NDArray[np.float64], zupt: NDArray[np.bool_],
                  configured: float) -> BiasWalk | None:
    """The bias walk a replay's stops show (module docstring), or None with fewer than
    :data:`MIN_INTERVALS` changes between stops or a ``configured`` walk of 0 (the bias held
    constant by choice).

    Args:
        t: (N,) s, the replay's rows. bias: (N,) rad/s, the filter's gyro bias after each.
        bias_var: (N,) (rad/s)^2, its variance. zupt: (N,) rows fused under a
            zero-velocity update. configured: (rad/s)^2/s, the walk fused with.
    """
    ends = [b for _, b in _stop_ends(t, zupt)]
    if not configured > 0.0 or len(ends) < MIN_INTERVALS + 1:
        return None  # a bias held constant by choice (bias_psd 0), or too few stops
    at = np.array(ends)

    def changes(stops: NDArray[np.int64]) -> tuple[NDArray[np.float64], ...]:
        """(changes rad/s, intervals s, variance floors) between consecutive ``stops``."""
        return (np.diff(bias[stops]), np.diff(t[stops]),
                bias_var[stops[:-1]] + bias_var[stops[1:]] + 2.0 * STOP_BIAS_STD ** 2)

    def chance(stops: NDArray[np.int64]) -> float:
        change, over, floor = changes(stops)
        return float(chi2.sf(np.sum(change * change / (configured * over + floor)),
                             change.size))

    # the test must hold with any one stop left out too: one stop's bias can be off (a
    # terrain bag's 1.6 s stop at the end of a slow creep was 0.1 deg/s off the rest, and
    # alone made a walk of 8.5 times the configured one, which cost 0.25 deg of yaw RMSE)
    p_value = max([chance(at)] + [chance(np.delete(at, k)) for k in range(at.size)])
    change, over, floor = changes(at)

    def nll(psd: float) -> float:
        var = psd * over + floor
        return float(np.sum(np.log(var) + change * change / var))

    best = minimize_scalar(lambda u: nll(math.exp(u)), method="bounded",
                           bounds=(math.log(configured), math.log(MAX_RAISE * configured)))
    psd = float(math.exp(best.x))
    if not nll(psd) < nll(configured):  # the optimum at the bound: the configured walk
        psd = configured
    i = int(np.argmax(np.abs(change)))
    return BiasWalk(psd, configured, int(change.size), p_value, float(abs(change[i])),
                    float(over[i]))
